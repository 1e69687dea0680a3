from setuptools import setup

package_name = 'pkm_bringup'

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
        'Running a scenario: scenario files, the orchestrator (pkm-run), its processes and realtime profile.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'pkm-run = pkm_bringup.run_cli:main',
        ],
    },
)
