from setuptools import setup

package_name = 'pkm_calibration'

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
        'Kinematic calibration: the error model of the bar model, its identification '
        'Jacobian, identifiability, and identification by nonlinear least squares.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'pkm-calibrate = pkm_calibration.cli:main',
        ],
    },
)
