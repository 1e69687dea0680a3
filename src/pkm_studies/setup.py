from setuptools import setup

package_name = 'pkm_studies'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    data_files=[
        ('share/ament_index/resource_index/packages',
            ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='PKM controller developers',
    maintainer_email='pkm-dev@pkm-controller.org',
    description=(
        'Studies: study files, the Dask runner, design sweeps and their tables.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'pkm-study = pkm_studies.study_engine:main',
        ],
    },
)
